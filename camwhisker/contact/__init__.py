"""Contact back end: GM (eq. 8), MF (eqs. 9-10), Z (eq. 11), fusion, shape (eq. 12)."""
