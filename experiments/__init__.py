"""Paper reproductions and their figures (the application layer: imports the library, never imported by it)."""
