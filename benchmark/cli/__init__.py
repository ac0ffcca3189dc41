"""The `bench` command line: `parser` builds every command's options from the settings dataclasses,
`main` dispatches to one module of commands per layer (`trial_commands`, `llm_commands`,
`training_commands`, `experiment_commands`, `evaluate_commands`, `check_commands`), `options` holds
what they share. The top layer: it may import every other; nothing imports it."""
