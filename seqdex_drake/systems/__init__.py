"""LeafSystems that run around the station: the operational-space approach controller, policies, switchers."""
