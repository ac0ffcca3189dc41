"""Token counting: GPT-4's tokenizer offline (bpe-openai, MIT, bundles cl100k_base) and the
embedded model's own tokenizer (llama.cpp's /tokenize endpoint on loopback)."""

from __future__ import annotations

import json
import urllib.request
from functools import cache

TOKENIZERS = ("gpt-4", "embedded")


@cache
def _cl100k():
    import bpe_openai

    return bpe_openai.get_encoding("cl100k_base")  # GPT-4's encoding; the package knows it by this name


def gpt4_tokens(text: str) -> int:
    return len(_cl100k().encode(text))


def server_tokens(base_url: str, text: str) -> int:
    """Tokens of `text` for the model a llama.cpp server serves (its /tokenize endpoint)."""
    root = base_url.removesuffix("/v1")
    request = urllib.request.Request(root + "/tokenize", data=json.dumps({"content": text}).encode(),
                                     headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(request, timeout=60) as response:
        return len(json.loads(response.read())["tokens"])
