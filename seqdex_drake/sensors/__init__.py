"""LeafSystems that read the station: the policy observations and the target block's pixel count."""
