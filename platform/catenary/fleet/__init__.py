"""What crosses machines: push and pull between vehicles and the central side."""
