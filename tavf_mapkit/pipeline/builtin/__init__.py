"""Pipeline stages. Every module here is imported by the runner and registers its stages itself."""
