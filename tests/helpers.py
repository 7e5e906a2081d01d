"""Assertions shared by the tests."""

from __future__ import annotations

from typing import Any

import numpy as np


def assert_same_message(actual: Any, expected: Any, path: str = "$") -> None:
    """Assert two decoded messages hold the same data.

    numpy arrays compare by dtype, shape and values; ``bytes`` and
    ``memoryview`` compare by content; everything else with ``==``.
    """
    if isinstance(expected, np.ndarray):
        assert isinstance(actual, np.ndarray), f"{path}: {type(actual).__name__} is not an array"
        assert actual.dtype == expected.dtype, f"{path}: dtype {actual.dtype} != {expected.dtype}"
        assert actual.shape == expected.shape, f"{path}: shape {actual.shape} != {expected.shape}"
        assert np.array_equal(actual, expected), f"{path}: values differ"
    elif isinstance(expected, (bytes, memoryview)):
        assert isinstance(actual, (bytes, memoryview)), f"{path}: {type(actual).__name__} is not binary"
        assert bytes(actual) == bytes(expected), f"{path}: bytes differ"
    elif isinstance(expected, dict):
        assert isinstance(actual, dict), f"{path}: {type(actual).__name__} is not an object"
        assert list(actual) == list(expected), f"{path}: keys {list(actual)} != {list(expected)}"
        for key in expected:
            assert_same_message(actual[key], expected[key], f"{path}[{key!r}]")
    elif isinstance(expected, list):
        assert isinstance(actual, list), f"{path}: {type(actual).__name__} is not a list"
        assert len(actual) == len(expected), f"{path}: length {len(actual)} != {len(expected)}"
        for index, (a, e) in enumerate(zip(actual, expected)):
            assert_same_message(a, e, f"{path}[{index}]")
    else:
        assert actual == expected, f"{path}: {actual!r} != {expected!r}"
