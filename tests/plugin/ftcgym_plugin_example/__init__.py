"""A user's policy, detector and scenario for ftcgym, from outside the package."""
