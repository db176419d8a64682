"""learner: meta-learned personalised neural surrogates (metaPNS). Built in a later issue."""
