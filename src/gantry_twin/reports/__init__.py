"""Reports over many runs: the paper's Tables 1-4 and figures, the rig report, runs compared side by side."""
