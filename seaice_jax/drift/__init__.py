"""Ice motion: drift vectors, transformation fits between point sets, deformation."""
