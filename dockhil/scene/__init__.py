"""Launch files: the reader, its schema, bounded YAML, and the graph a scene builds."""
