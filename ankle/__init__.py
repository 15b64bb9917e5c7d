"""The ``ankle`` command: one entry point to every part of the system.

This is the composition root, above every other package: it may import any of them and
none imports it.
"""
