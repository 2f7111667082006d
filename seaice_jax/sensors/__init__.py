"""How raw measurements become geometry inputs (navigation records, radar image coordinates)."""
