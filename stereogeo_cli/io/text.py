"""Text formatting: the numbers of the YAML writers (ROS, Kalibr) and COLMAP's text file, and the counts
of messages."""

from __future__ import annotations

from collections.abc import Iterable


def yaml_float(value: float) -> str:
    """Shortest text that reads back to the same float64 *as a float* in every YAML parser.

    PyYAML (YAML 1.1) reads ``1e-05`` as a string: a float needs a dot, so that becomes ``1.0e-05``.
    """
    text = repr(float(value))
    if "e" in text and "." not in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent}"
    return text


def flow_list(values: Iterable[float]) -> str:
    """``[a, b, c]`` with :func:`yaml_float` numbers."""
    return "[" + ", ".join(yaml_float(v) for v in values) + "]"


def plural(count: int, word: str, words: str | None = None) -> str:
    """``count`` and ``word``, in the plural unless ``count`` is 1 (``words``, else ``word`` + "s"):
    ``"1 pair"``, ``"0 pairs"``, ``"3 pairs"``."""
    return f"{count} {word if count == 1 else words or word + 's'}"
