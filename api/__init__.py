"""The tuning service: FastAPI app around :mod:`tuner` (see :func:`api.main.create_app`)."""
