"""Universal Robots backend over the unmodified ur_rtde (docs/ur.md). ur_rtde is imported inside
`driver`'s functions only, so this package imports without it."""
