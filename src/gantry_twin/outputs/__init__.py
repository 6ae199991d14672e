"""What a run leaves behind: run directories, atomic files, stop signals, the trace file, the typed summary, plots."""
