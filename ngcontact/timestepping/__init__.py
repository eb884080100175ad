"""Time-dependent contact: backward Euler / P_p step systems, the time-stepping driver, space-time estimators."""
