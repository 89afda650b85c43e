"""softsbi-toy: a third-party plugin package for softsbi's tests."""
