"""Writers: G-code, JSON report, PNG figures, HTML viewer. All write atomically."""
