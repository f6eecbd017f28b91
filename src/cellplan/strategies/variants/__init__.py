"""The Section VI model variants (simultaneous requests, time-varying regions)."""
