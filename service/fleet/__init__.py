"""Where the trainers run: threads of this process (default) or Ray actors (docs/fleet.md).
Every executor hands out :class:`~service.fleet.executor.TrainerHandle` objects."""
