"""Cross-cutting pieces of the service: configuration."""
