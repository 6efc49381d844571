"""Visualisation: the Rerun recording of a run (twin.viz.rerun_log)."""
