"""How gains are chosen: design helpers, the search space, scoring, the global and local stages.

``design`` (plant scale, plant-based starts, bounds), ``space`` (search coordinates),
``scoring`` (verifier-backed score of a candidate), ``search`` (everything Optuna) and
``nlp/`` (everything CasADi). The facade that runs them is :func:`tuner.tune`.
"""
