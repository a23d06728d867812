"""``siva replay`` (plan, run, verdict) and start-up reconciliation of the event log with
the store (docs/logs.md)."""
