"""Settings: a stage's defaults with the overrides its caller gives, in one place.

Every stage keeps its defaults in a module-level ``default_conf`` dict and takes a ``conf`` of overrides.
:func:`resolve` merges the two key by key, nested settings included: overriding one key of a nested block
(``{"colmap": {"mapping": {"ba_global_max_num_iterations": 50}}}``) keeps that block's other defaults.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def resolve(defaults: Mapping[str, Any], overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``defaults`` with ``overrides`` merged in, nested mappings merged the same way, as a new dict whose
    nested dicts are new too (neither argument is changed, and a caller that changes the result changes
    no default)."""
    merged: dict[str, Any] = {}
    for key, value in defaults.items():
        merged[key] = resolve(value) if isinstance(value, Mapping) else value
    for key, value in (overrides or {}).items():
        base = merged.get(key)
        if isinstance(base, Mapping) and isinstance(value, Mapping):
            merged[key] = resolve(base, value)
        else:
            merged[key] = resolve(value) if isinstance(value, Mapping) else value
    return merged
