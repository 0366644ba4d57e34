"""Developer tools that are not part of the installed product (run from the project directory)."""
