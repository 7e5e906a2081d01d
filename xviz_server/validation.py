"""Validation of XVIZ messages against the XVIZ v2 JSON Schema.

The schema files are package data of :mod:`xviz_server.schema`, one file
per schema name: ``session/state_update`` is ``session/state_update.json``.
They refer to each other by relative ``$ref`` and are loaded once into a
:class:`referencing.Registry`. Use the shared instance::

    from xviz_server.validation import get_validator

    get_validator().validate("session/metadata", metadata)
    get_validator().validate_message({"type": "xviz/state_update", "data": update})

Messages decoded from GLB are not plain JSON values. Before validation, a
copy of the instance is made JSON-like; the caller's object is left alone:

* a numpy array becomes a list of its first 64 rows (all of it when it is
  shorter). Every row of an array has the same shape and dtype, so these
  rows stand for the others, and no XVIZ ``minItems`` exceeds 64. A float
  array holding NaN or infinity is reported at the path of its first
  non-finite value, since JSON numbers are finite;
* a list of more than 64 numbers or of equal-length lists of numbers (a
  point cloud decoded from JSON) is treated like the numpy array it
  stands for: its first 64 rows are validated and it is checked for
  non-finite values;
* a numpy scalar becomes the matching Python scalar;
* ``bytes``, ``bytearray`` and ``memoryview`` (encoded images) become a
  short placeholder string, as images are base64 strings in JSON XVIZ;
* a tuple becomes a list.

A non-finite Python ``float`` is reported as well.
"""

from __future__ import annotations

import difflib
import functools
import json
import math
import reprlib
from collections.abc import Iterable, Iterator
from importlib import resources
from typing import TYPE_CHECKING, Any

import numpy as np
from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError, best_match
from referencing import Registry
from referencing.jsonschema import DRAFT202012

from .exceptions import SchemaValidationError, UnknownSchemaError

if TYPE_CHECKING:
    from importlib.abc import Traversable

__all__ = ["ARRAY_ROWS", "XVIZValidator", "get_validator"]

#: Rows of a numpy array that are validated.
ARRAY_ROWS = 64

_Location = tuple[str | int, ...]
_Problem = tuple[_Location, str]

_short = reprlib.Repr()
_short.maxstring = _short.maxother = 40
_short.maxlist = _short.maxdict = 3
_short.maxlevel = 2


class XVIZValidator:
    """Validates instances against the XVIZ v2 schemas, chosen by name.

    A name is a schema file's path below the schema folder without its
    ``.json`` suffix, e.g. ``"session/start"`` or ``"primitives/point"``.
    """

    def __init__(self) -> None:
        schemas = dict(_read_schemas(resources.files("xviz_server.schema")))
        registry = (
            Registry()
            .with_resources((schema["$id"], DRAFT202012.create_resource(schema)) for schema in schemas.values())
            .crawl()
        )
        self._validators = {
            name: Draft202012Validator(schema, registry=registry) for name, schema in sorted(schemas.items())
        }

    def names(self) -> list[str]:
        """Return the names of all schemas, sorted."""
        return list(self._validators)

    def errors(self, name: str, instance: Any) -> list[str]:
        """Return the violations of schema *name* by *instance*, ordered by path.

        Each line starts with the JSON path of the offending value, e.g.
        ``$.updates[0].primitives['/lidar/points'].points[0].colors: ...``.
        An empty list means the instance is valid.

        Raises :class:`UnknownSchemaError` if there is no schema *name*.
        """
        validator = self._validator(name)
        problems: list[_Problem] = []
        instance = _json_like(instance, (), problems)
        for error in validator.iter_errors(instance):
            problems.extend(_explain(error))
        problems.sort(key=lambda problem: [(isinstance(key, str), key) for key in problem[0]])
        lines = (f"{_json_path(path)}: {message}" for path, message in problems)
        return list(dict.fromkeys(lines))

    def validate(self, name: str, instance: Any) -> None:
        """Check *instance* against schema *name*.

        Raises :class:`~xviz_server.exceptions.SchemaValidationError`
        listing every violation, or :class:`UnknownSchemaError` if there
        is no schema *name*.
        """
        problems = self.errors(name, instance)
        if problems:
            raise SchemaValidationError(name, problems)

    def validate_message(self, envelope: Any) -> None:
        """Check an envelope, and its data against the schema of its ``xviz/`` type.

        Raises :class:`~xviz_server.exceptions.SchemaValidationError`.
        """
        self.validate("envelope", envelope)

    def _validator(self, name: str) -> Draft202012Validator:
        try:
            return self._validators[name]
        except KeyError:
            close = difflib.get_close_matches(name, self._validators, n=3, cutoff=0.5)
            hint = f"did you mean {', '.join(map(repr, close))}?" if close else "see XVIZValidator.names()"
            raise UnknownSchemaError(f"no XVIZ schema named {name!r}; {hint}") from None


@functools.cache
def get_validator() -> XVIZValidator:
    """Return the shared :class:`XVIZValidator`, loading the schemas on first use."""
    return XVIZValidator()


def _read_schemas(folder: Traversable, prefix: str = "") -> Iterator[tuple[str, dict[str, Any]]]:
    """Yield ``(name, schema)`` for every schema file below *folder*."""
    for entry in folder.iterdir():
        if entry.is_dir():
            yield from _read_schemas(entry, f"{prefix}{entry.name}/")
        elif entry.name.endswith(".json"):
            yield prefix + entry.name.removesuffix(".json"), json.loads(entry.read_text("utf-8"))


def _json_like(value: Any, path: _Location, problems: list[_Problem]) -> Any:
    """Return a JSON-like copy of *value*, as described in the module docstring."""
    if isinstance(value, dict):
        return {key: _json_like(item, (*path, key), problems) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        if len(value) > ARRAY_ROWS:
            block = _numeric_block(value)
            if block is not None:
                _check_finite(block, path, problems)
                value = value[:ARRAY_ROWS]
        return [_json_like(item, (*path, index), problems) for index, item in enumerate(value)]
    if isinstance(value, float):
        if not math.isfinite(value):
            problems.append((path, f"{value} is not a finite number"))
        return value
    if isinstance(value, np.ndarray):
        _check_finite(value, path, problems)
        return value.tolist() if value.ndim == 0 else value[:ARRAY_ROWS].tolist()
    if isinstance(value, np.generic):
        return _json_like(value.item(), path, problems)
    if isinstance(value, (bytes, bytearray, memoryview)):
        return f"<{memoryview(value).nbytes} bytes>"
    return value


def _numeric_block(value: list[Any] | tuple[Any, ...]) -> np.ndarray | None:
    """*value* as a float array if it is a rectangular block of numbers, else ``None``."""
    first = value[0]
    if isinstance(first, bool) or not isinstance(first, (int, float, list, tuple)):
        return None
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    return array if array.ndim <= 2 else None


def _check_finite(array: np.ndarray, path: _Location, problems: list[_Problem]) -> None:
    """Report the first NaN or infinity of a float *array*, with their count."""
    if array.dtype.kind != "f":
        return
    bad = ~np.isfinite(array)
    count = int(np.count_nonzero(bad))
    if count:
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        message = f"{float(array[index])} is not a finite number"
        if count > 1:
            message += f" ({count} non-finite values in this array)"
        problems.append(((*path, *index), message))


def _explain(error: ValidationError) -> Iterator[_Problem]:
    """Yield the path and a one-line description of each violation behind *error*."""
    path = tuple(error.absolute_path)
    if error.validator in ("anyOf", "oneOf") and error.context:
        yield from _explain_alternatives(error, path)
    elif error.validator == "not":
        yield path, f"{_short.repr(error.instance)} is not allowed here"
    elif error.validator == "pattern" and "title" in error.schema:
        yield path, f"{_short.repr(error.instance)} is not a valid {error.schema['title']}"
    else:
        message = error.message
        full = repr(error.instance)
        if len(full) > 80:
            message = message.replace(full, _short.repr(error.instance))
        yield path, message


def _explain_alternatives(error: ValidationError, path: _Location) -> Iterator[_Problem]:
    """Explain a failed ``anyOf``/``oneOf`` by the alternative the instance was meant to be.

    Alternatives that reject the type of the instance are set aside; of the
    others, the one with the fewest errors (then the fewest type errors) is
    taken. On a tie, the titles of the candidates are listed.
    """
    if all(cause.validator == "required" for cause in error.context):
        names = ", ".join(repr(name) for cause in error.context for name in cause.validator_value)
        yield path, f"needs one of {names}"
        return
    by_alternative: dict[int, list[ValidationError]] = {}
    for cause in error.context:
        by_alternative.setdefault(cause.relative_schema_path[0], []).append(cause)
    candidates = {
        index: causes
        for index, causes in by_alternative.items()
        if not any(cause.validator == "type" and len(cause.absolute_path) == len(path) for cause in causes)
    } or by_alternative
    ranks = {index: _distance(causes) for index, causes in candidates.items()}
    nearest = min(ranks.values())
    closest = [candidates[index] for index, rank in ranks.items() if rank == nearest]
    titles = [error.validator_value[index].get("title") for index in candidates]
    if len(closest) == 1:
        for cause in closest[0]:
            yield from _explain(cause)
    elif all(titles):
        yield path, f"{_short.repr(error.instance)} is none of: {'; '.join(titles)}"
    else:
        yield from _explain(best_match(error.context))


def _distance(causes: list[ValidationError]) -> tuple[int, int]:
    """How far an instance is from an alternative, by the errors it raised there."""
    return len(causes), sum(cause.validator == "type" for cause in causes)


def _json_path(path: Iterable[str | int]) -> str:
    """Format a path as JSONPath: ``$.updates[0].primitives['/lidar/points']``."""
    parts = ["$"]
    for key in path:
        if isinstance(key, int):
            parts.append(f"[{key}]")
        elif key.isidentifier():
            parts.append(f".{key}")
        else:
            parts.append(f"[{key!r}]")
    return "".join(parts)
