"""The LLM controller: prompts, number encodings, models and the LLM policy."""
