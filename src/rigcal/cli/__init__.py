"""The ``rigcal`` command: a thin shell over the library."""
