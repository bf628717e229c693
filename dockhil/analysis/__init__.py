"""What a scene will do and what a run did: the scene check, run summaries (1-DOF and 6-DOF), the
report, the figures and plots, campaigns (sweep) and what each node type costs (leanness)."""
