"""Running and evaluating whole chains: the runner (station + chain controller, per-object episodes), the meshcat
status display, ``seqdex evaluate``'s experiments, tables and plots."""
