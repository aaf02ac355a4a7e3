"""Import and export of other photogrammetric programs' files (issue 17)."""
