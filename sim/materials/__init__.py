"""Dr.Jit reflectance models (placeholder until the material library lands)."""
