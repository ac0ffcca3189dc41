"""Token counting: GPT-4's tokenizer offline (bpe-openai, MIT, bundles cl100k_base) and the
embedded model's own tokenizer (llama.cpp's /tokenize endpoint on loopback)."""

from __future__ import annotations

from functools import cache

TOKENIZERS = ("gpt-4", "embedded")


@cache
def _cl100k():
    import bpe_openai

    return bpe_openai.get_encoding("cl100k_base")  # GPT-4's encoding; the package knows it by this name


def gpt4_tokens(text: str) -> int:
    return len(_cl100k().encode(text))


def server_tokens(base_url: str, text: str) -> int:
    """Tokens of `text` for the model a llama.cpp server serves (its /tokenize endpoint, through the SDK's client)."""
    import openai

    with openai.OpenAI(base_url=base_url.removesuffix("/v1"), api_key="none", max_retries=1) as client:
        return len(client.post("/tokenize", body={"content": text}, cast_to=object)["tokens"])
