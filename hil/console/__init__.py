"""`pure-hil console`: the rig's screen in a browser, a zenoh client of `pure-hil serve` (docs/rig.md)."""
