"""Rollout workers: the same class runs serially and inside Ray actors."""
