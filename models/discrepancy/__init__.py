"""The discrepancy workflow: find where a physics model and a measurement disagree, name the\nmissing effect, add it, and show the held-out gap shrink (pure core; see workflow.py)."""
