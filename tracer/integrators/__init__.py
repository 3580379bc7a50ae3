"""Light transport estimators: the report's branching estimator and a path tracer with MIS."""
