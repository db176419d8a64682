"""simgen: Aliev-Panfilov simulation-data service."""
