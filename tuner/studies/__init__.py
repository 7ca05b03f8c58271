"""Studies: many loops tuned at once from a TOML file.

``schema`` (the study file), ``evaluate`` (tuning and verifying loops, cascades included),
``runner`` (workers sharing a study through an Optuna storage), ``report`` (Markdown) and
``cli`` (``tuner study run``, ``tuner verify``).
"""
