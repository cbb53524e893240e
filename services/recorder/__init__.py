"""The recorder: every fixstream stream on a key expression to chunked, compressed MCAP files."""
