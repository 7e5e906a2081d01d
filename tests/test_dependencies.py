"""The modules that rely on a library's internals refuse a release they were not tested with."""

from __future__ import annotations

import subprocess
import sys

import pytest

from xviz_server.exceptions import DependencyError
from xviz_server.version import require_tested


def test_a_release_not_tested_is_refused_with_how_to_install_a_tested_one():
    tested = frozenset({(17, 4), (18, 0)})
    require_tested("xviz_server.framing", "websockets", "17.4.1", tested, "pip install -e .")
    require_tested("xviz_server.framing", "websockets", "18.0rc1", tested, "pip install -e .")
    for installed in ["17.5", "16.4.2", "unknown"]:
        with pytest.raises(DependencyError) as refused:
            require_tested("xviz_server.framing", "websockets", installed, tested, "pip install -e .")
        assert str(refused.value) == (
            f"xviz_server.framing was tested with websockets 17.4, 18.0, not {installed}: "
            "install a tested release (pip install -e .) or test xviz_server.framing with the new one and add it"
        )


@pytest.mark.parametrize(
    ("module", "library", "attribute"),
    [
        ("xviz_server.framing", "websockets.version", "version"),
        ("xviz_server.live.redis_wire", "redis", "__version__"),
    ],
)
def test_importing_a_guarded_module_with_another_release_fails_at_once(module: str, library: str, attribute: str):
    pytest.importorskip(library)
    # The library as installed, but claiming a release no one tested.
    code = f"import {library}; {library}.{attribute} = '0.1.0'; import {module}"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert f"DependencyError: {module} was tested with " in result.stderr and ", not 0.1.0: install" in result.stderr
