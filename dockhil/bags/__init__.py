"""MCAP bags: the writer, the (recovering) reader, the tools (info, CSV export, convert), recording and
replay on a running graph, and the live view in Foxglove."""
