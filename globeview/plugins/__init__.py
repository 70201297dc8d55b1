"""Plugin API and registry; the built-in LOD providers and tools (no Qt)."""
