"""The Rutgers Ankle device: controller, plant simulation and protocol.

Runs alone on the embedded PC: nothing here imports the server, the station or the web UI.
Pure code (kinematics, control laws, plant model) does no I/O; I/O sits at the edge.
"""

from importlib.metadata import PackageNotFoundError, version

__version__ = "0.1.0"
"""The one place the version is written: pyproject.toml reads it from here."""


def installed_version() -> str:
    """The installed distribution's version (``ankle --version``, ``/health``)."""
    try:
        return version("ankle-telerehab")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return f"{__version__}+source"
