"""The public API: what ``xviz_server`` exports, and that ``import xviz_server`` stays cheap."""

from __future__ import annotations

import subprocess
import sys

import pytest

import xviz_server
from xviz_server import builder, exceptions, live, probe, server, settings, writer

EXPECTED = {
    "XVIZServer": server.XVIZServer,
    "Settings": settings.Settings,
    "LiveFeed": live.LiveFeed,
    "MetadataBuilder": builder.MetadataBuilder,
    "FrameBuilder": builder.FrameBuilder,
    "LogWriter": writer.LogWriter,
    "ProbeReport": probe.ProbeReport,
    **{name: getattr(exceptions, name) for name in exceptions.__all__},
}


def test_every_public_name_is_exported_and_is_the_real_object():
    assert set(xviz_server.__all__) == {*EXPECTED, "__version__"}
    for name, value in EXPECTED.items():
        assert getattr(xviz_server, name) is value, name
    assert {*EXPECTED} <= set(dir(xviz_server))


def test_every_exception_derives_from_xviz_error():
    for name in exceptions.__all__:
        assert issubclass(getattr(xviz_server, name), xviz_server.XVIZError), name


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Serverr'"):
        xviz_server.Serverr  # noqa: B018


def test_importing_the_package_imports_nothing_heavy():
    code = "import sys, xviz_server; print(sorted(m for m in sys.modules if m.split('.')[0] in ('websockets', 'numpy', 'xviz_server')))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "['xviz_server', 'xviz_server.exceptions']"


def test_the_package_declares_its_type_hints():
    from importlib.resources import files

    assert files("xviz_server").joinpath("py.typed").is_file()
