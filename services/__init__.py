"""fixstream services: one package per process (pure core + thin Zenoh adapter)."""
