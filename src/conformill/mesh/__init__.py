"""Mesh stage: reading (io), topology (boundary loops, Euler characteristic), validation."""
