"""The bench's independent judges: reference implementations from other libraries (Pinocchio) used to check ours."""
