"""Many runs: campaigns and their coverage judgement, HACS/iHACS comparison, replay, the pytest plugin."""
