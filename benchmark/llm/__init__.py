"""The LLM controller: prompts, encodings, prompt strategies, reply parsing, models (embedded
llama.cpp, OpenAI-compatible servers, text-only reference models) and the LLM policy that runs the
paper's protocol inside a trial. May import `benchmark.trial` and `benchmark.common`."""
