"""What users hand in and get out: configuration, physical bounds, parser guards, file names and
the output rule."""
