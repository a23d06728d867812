"""HTTP only: the FastAPI app, its routes (one module per resource), dependencies, the
mapping of domain errors to status codes, dashboard and metrics."""
