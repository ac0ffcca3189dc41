"""Scoring models: the teacher-forced imitation probe and its probe set (`probe`, `data/`), one
scorecard per model from a suite tier (`scorecard`, `suites/`), and the leaderboard with its page
(`leaderboard`, `leaderboard_html`). May import `benchmark.experiments` and every layer below."""
