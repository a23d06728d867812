"""What is on disk: systems and recordings (the store), checkpoints, the event log.

The front process is the only writer of systems and recordings; trainers read through
``trainer_view.py``.  See docs/service.md, "Layout".
"""
