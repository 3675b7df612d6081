"""Built-in wire types."""
