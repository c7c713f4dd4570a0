"""The reglib HTTP service (FastAPI): ``create_app`` in :mod:`service.app`; run it with ``reglib serve``."""
