"""Low-level controllers on the station: the operational-space controller and its parameters."""
