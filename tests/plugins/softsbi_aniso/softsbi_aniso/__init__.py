"""softsbi-aniso: a third-party effect package (anisotropic table friction), see :mod:`.plugin`."""
