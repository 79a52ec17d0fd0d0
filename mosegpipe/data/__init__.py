"""Dataset readers and synthetic generators. Readers take a root folder and never download."""
