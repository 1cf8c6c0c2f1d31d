"""The control laws: seed forms, predictive, mid-ranging, two elements, learning, reach."""
