"""The Rutgers Ankle device: controller, plant simulation and protocol.

Runs alone on the embedded PC: nothing here imports the server, the station or the web UI.
Pure code (kinematics, control laws, plant model) does no I/O; I/O sits at the edge.
"""

__version__ = "0.1.0"
