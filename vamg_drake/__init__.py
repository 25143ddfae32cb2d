"""Visibility-aware mobile grasping in dynamic environments, as a Drake systems diagram."""
