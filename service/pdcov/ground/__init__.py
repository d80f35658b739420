"""The ground station (`pdcov watch`): terminal view and web map."""
