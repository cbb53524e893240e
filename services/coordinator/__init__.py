"""Base-station coordinator core (digest 002 §2.4, §4.8, §7.3 S7): registry, departure rule, beacon sets."""
