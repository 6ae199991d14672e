"""Machine health: excitation of the estimates (eq. 29), trust in them, the CUSUM monitor, the monitor over logs."""
