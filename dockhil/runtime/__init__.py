"""The graph at run time: transport, executor and message screen, composed runs and containers,
node processes, the launcher and its registry, device ownership, and whether a run is valid."""
