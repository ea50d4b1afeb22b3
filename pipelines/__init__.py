"""End-to-end flows: demo, evaluation, benchmarks, visualisation entry points."""
