"""The paper's five ways of writing numbers into a prompt, each with its exact inverse.

E1 original values (two decimals), E2 shifted positive (two decimals), E3 integers (x10,
signed), E4 decimals dropped then shifted positive (the paper code's int((round(x, 1) + 5) * 10):
[-5, 5] -> 0..100), E5 positive integers (default: [-10, 10] -> 0..200, one token per value
for GPT-4's tokenizer). Decoding an encoded value returns it to the encoding's resolution.

Compact variants (E4c, E5c) write the same numbers without the space after each comma: for tokenizers that
split digits (Gemma, Qwen) a value then costs its digits and one comma instead of a comma and a space as well
(E5: ~5 tokens a value, E5c ~4; E4c ~3, its values mostly two digits). Labelled, never the default: a variant
changes the text a model reads, so its results are its own (`bench throughput`, the probe and the closed loop
measure each).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robots import UnknownNameError


@dataclass(frozen=True)
class Encoding:
    name: str
    title: str
    scale: float  # value * scale before rounding
    offset: float  # added before scaling, so the result is non-negative
    decimals: int  # 0: integers
    low: float  # values are clipped to [low, high] first
    high: float
    separator: str = ", "  # between values; "," in the compact variants

    @property
    def label(self) -> str:
        """The encoding as reports name it."""
        return self.title + (" (compact: no space after the comma)" if self.separator == "," else "")

    def encode_value(self, x: float) -> str:
        y = (float(np.clip(x, self.low, self.high)) + self.offset) * self.scale
        return str(int(round(y))) if self.decimals == 0 else f"{y:.{self.decimals}f}"

    def encode(self, values: np.ndarray) -> str:
        return "[" + self.separator.join(self.encode_value(v) for v in np.asarray(values, dtype=float)) + "]"

    def quantize(self, values: np.ndarray) -> np.ndarray:
        """`values` as written in this encoding and read back: the closest answer a reply can give."""
        return self.decode([float(self.encode_value(v)) for v in np.asarray(values, dtype=float)])

    def decode(self, numbers: list[float]) -> np.ndarray:
        return np.clip(np.asarray(numbers, dtype=float) / self.scale - self.offset, self.low, self.high)

    @property
    def resolution(self) -> float:
        return 10.0**-self.decimals / self.scale

    @property
    def integer_range(self) -> tuple[int, int] | None:
        """(min, max) of the encoded integers, for grammars; None for decimal encodings."""
        if self.decimals:
            return None
        return int(round((self.low + self.offset) * self.scale)), int(round((self.high + self.offset) * self.scale))


ENCODINGS: dict[str, Encoding] = {
    "E1": Encoding("E1", "original values", 1.0, 0.0, 2, -10.0, 10.0),
    "E2": Encoding("E2", "shifted to positive", 1.0, 10.0, 2, -10.0, 10.0),
    "E3": Encoding("E3", "integers (x10)", 10.0, 0.0, 0, -10.0, 10.0),
    "E4": Encoding("E4", "decimals dropped, shifted positive (0..100)", 10.0, 5.0, 0, -5.0, 5.0),
    "E5": Encoding("E5", "positive integers (0..200)", 10.0, 10.0, 0, -10.0, 10.0),
    "E4c": Encoding("E4c", "decimals dropped, shifted positive (0..100)", 10.0, 5.0, 0, -5.0, 5.0, separator=","),
    "E5c": Encoding("E5c", "positive integers (0..200)", 10.0, 10.0, 0, -10.0, 10.0, separator=","),
}
DEFAULT_ENCODING = "E5"


def get_encoding(name: str) -> Encoding:
    if name not in ENCODINGS:
        raise UnknownNameError("encoding", name, list(ENCODINGS))
    return ENCODINGS[name]
