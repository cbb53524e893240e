"""fixstream runtime: configuration, Zenoh sessions, the wire codec, the service base, the stack runner."""
