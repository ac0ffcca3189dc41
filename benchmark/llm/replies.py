"""Constraining and parsing the model's answer: 12 numbers in the encoding's range."""

from __future__ import annotations

import json
import re

import numpy as np

from benchmark.llm.encodings import Encoding

NUMBER = re.compile(r"-?\d+(?:\.\d+)?")
BRACKETS = re.compile(r"\[([^\[\]]*)\]")


def parse_reply(text: str, enc: Encoding, count: int = 12) -> np.ndarray | None:
    """Decoded actions from the first bracketed list (or a JSON {"output": [...]}), or None."""
    stripped = text.strip()
    if stripped.startswith("{"):
        try:
            values = json.loads(stripped)["output"]
            numbers = [float(v) for v in values]
        except (ValueError, KeyError, TypeError):
            return None
    else:
        match = BRACKETS.search(text)
        if match is None:
            return None
        numbers = [float(n) for n in NUMBER.findall(match.group(1))]
        if len(match.group(1).split(",")) != len(numbers):
            return None
    if len(numbers) != count:
        return None
    return enc.decode(numbers)


def _int_rule(low: int, high: int) -> str:
    """GBNF alternatives for the integers 0..high (high a multiple of 100), signed if low < 0."""
    if high % 100 or low not in (0, -high):
        raise ValueError(f"no grammar for the range {low}..{high}")
    hundreds = high // 100
    options = ["[0-9]", "[1-9] [0-9]"]
    if hundreds >= 2:
        options.append(f"[1-{hundreds - 1}] [0-9] [0-9]" if hundreds > 2 else '"1" [0-9] [0-9]')
    options.append(f'"{high}"')
    body = " | ".join(options)
    return f'num ::= "-"? ({body})' if low < 0 else f"num ::= {body}"


def gbnf_grammar(enc: Encoding, count: int = 12) -> str:
    """A llama.cpp grammar forcing `[n, n, ..., n]` with `count` numbers in the encoding's range."""
    if enc.integer_range is None:
        whole = int(max(abs(enc.low), abs(enc.high)) + enc.offset)
        digits = len(str(whole))
        sign = '"-"? ' if enc.low + enc.offset < 0 else ""
        num = f"num ::= {sign}[0-9]{{1,{digits}}} \".\" " + " ".join(["[0-9]"] * enc.decimals)
    else:
        num = _int_rule(*enc.integer_range)
    separator = " ".join(f'"{c}"' for c in enc.separator)  # "," " " or ","
    return f'root ::= " "? "[" num ({separator} num){{{count - 1}}} "]"\n{num}\n'


def json_schema(enc: Encoding, count: int = 12) -> dict:
    """An OpenAI structured-output schema: {"output": [count numbers in range]}."""
    if enc.integer_range is None:
        low, high = (enc.low + enc.offset) * enc.scale, (enc.high + enc.offset) * enc.scale
        item = {"type": "number", "minimum": low, "maximum": high}
    else:
        low, high = enc.integer_range
        item = {"type": "integer", "minimum": low, "maximum": high}
    return {"name": "joint_targets", "strict": True, "schema": {
        "type": "object", "additionalProperties": False, "required": ["output"],
        "properties": {"output": {"type": "array", "items": item, "minItems": count, "maxItems": count}}}}


def reply_regex(enc: Encoding, count: int = 12) -> str:
    """The grammar's rule as a regular expression (vLLM's and SGLang's constraint field)."""
    if enc.integer_range is None:
        whole = len(str(int(max(abs(enc.low), abs(enc.high)) + enc.offset)))
        sign = "-?" if enc.low + enc.offset < 0 else ""
        num = f"{sign}[0-9]{{1,{whole}}}\\.[0-9]{{{enc.decimals}}}"
    else:
        low, high = enc.integer_range
        num = ("-?" if low < 0 else "") + f"[0-9]{{1,{len(str(high))}}}"
    return f"\\[{num}({enc.separator}{num}){{{count - 1}}}\\]"  # "," and " " need no escaping


def reply_constraint(enc: Encoding, count: int = 12, constrained: bool = True):
    """The output constraint a reply is held to, written in every dialect (each model sends the one its
    server reads); no constraint when `constrained` is off (the paper's setting)."""
    from benchmark.llm.models import Constraint

    if not constrained:
        return Constraint()
    return Constraint(grammar=gbnf_grammar(enc, count), schema=json_schema(enc, count), regex=reply_regex(enc, count))
