"""The pure core: physics, estimator, gate, adaptation, discrepancy. Arrays in, arrays out."""

if __name__ != "wrenchd.models":  # the folder on sys.path is not the package
    raise ImportError(f"import wrenchd.models, not {__name__}: wrenchd installs one import name")
