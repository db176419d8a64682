"""learner: meta-learned personalised neural surrogates (metaPNS) and the generic PNS.

Trains on episodes read from a simgen dataset store, evaluates, personalises from a few observed
simulations, predicts new stimulation sites, and compares with Bayesian-optimisation baselines
(docs/surrogate.md).
"""
