"""The runtime (daemon, pipeline), replay, the command line, studies and benches."""

if __name__ != "wrenchd.service":  # the folder on sys.path is not the package
    raise ImportError(f"import wrenchd.service, not {__name__}: wrenchd installs one import name")
