"""Test helpers that record the calls of a function or method and let each call go through."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest


def recorded(values: list[Any], key: Callable[..., Any], function: Callable[..., Any]) -> Any:
    """``function``, appending ``key`` of its arguments to ``values`` at every call."""

    def recording(*args: Any, **kwargs: Any) -> Any:
        values.append(key(*args, **kwargs))
        return function(*args, **kwargs)

    return recording


def counted(calls: list[str], name: str, function: Callable[..., Any]) -> Any:
    """``function``, appending ``name`` to ``calls`` at every call."""
    return recorded(calls, lambda *_args, **_kwargs: name, function)


def record_method(
    monkeypatch: pytest.MonkeyPatch, owner: type, name: str, key: Callable[..., Any]
) -> list[Any]:
    """``key`` of the arguments (after ``self``) of every later call of ``owner.<name>``."""
    values: list[Any] = []
    method = getattr(owner, name)
    monkeypatch.setattr(owner, name, recorded(values, lambda _self, *args: key(*args), method))
    return values
