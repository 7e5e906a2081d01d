"""This package's version, and the check that a library whose internals a module relies on is a tested release."""

from __future__ import annotations

import re

from .exceptions import DependencyError

__all__ = ["__version__", "require_tested"]

__version__ = "0.1.0"


def require_tested(module: str, library: str, installed: str, tested: frozenset[tuple[int, int]], install: str) -> None:
    """Raise :class:`~xviz_server.exceptions.DependencyError` unless release ``installed`` of ``library`` is tested.

    ``module`` relies on internals of ``library`` that may change in any
    release: it was tested with the releases ``tested`` ((major, minor)
    pairs). The error names the command that installs a tested release,
    ``install``.
    """
    release = re.match(r"(\d+)\.(\d+)", installed)
    if release is None or (int(release[1]), int(release[2])) not in tested:
        raise DependencyError(
            f"{module} was tested with {library} {', '.join(f'{a}.{b}' for a, b in sorted(tested))}, not {installed}: "
            f"install a tested release ({install}) or test {module} with the new one and add it"
        )
