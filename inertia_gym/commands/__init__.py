"""Sub-commands of the `inertia-gym` CLI (thin shells over the library)."""
