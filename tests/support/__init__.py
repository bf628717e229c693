"""Helpers of the test suite: node types the test graphs run (graphnodes, faultnodes, lognodes, bagnodes),
bags they write (bagfiles) and graphs run in this process (inprocess)."""
