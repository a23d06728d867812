"""Per-record fits, the headline they give, and drift detection on them (docs/service.md,
"Drift").  Knows nothing of trainers, threads or HTTP."""
