"""The run pipeline: a bench and a scenario in, a judged run out (build, tick loop, judge)."""
