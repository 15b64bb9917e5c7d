"""The serial link between the device and the home station: framing and messages."""
