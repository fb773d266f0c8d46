"""The chain as Drake systems: policies, feasibility inference, the switcher and the chain controller diagram."""
