"""Physical simulation of the Rutgers Ankle: valves, chambers, cylinders, platform, foot."""
