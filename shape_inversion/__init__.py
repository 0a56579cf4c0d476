"""SMPL-SI: map a custom character's skeleton to SMPL shape (beta) and a global scale."""
