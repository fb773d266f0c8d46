"""Scripted bases of the sub-tasks: the controllers a residual policy corrects, and the grasp planner."""
