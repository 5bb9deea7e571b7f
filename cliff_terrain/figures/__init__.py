"""Pictures for people: colour maps, legends, annotated views and contact sheets, and the files
of a rendered relief (``outputs``: their names and their one writer)."""
