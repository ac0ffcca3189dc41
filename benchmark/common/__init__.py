"""Shared utilities every layer may use: typed settings (`settings`), the results store (`store`),
interrupt handling (`interrupt`), the platform fingerprint (`fingerprint`) and table helpers
(`tables`). Imports nothing else of `benchmark`; `robots` only for its error type."""
