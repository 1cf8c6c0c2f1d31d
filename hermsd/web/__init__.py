"""`hermsd web`: the brewer's page, a process of its own that speaks to the daemon only through
the control socket (the daemon never serves HTTP)."""
