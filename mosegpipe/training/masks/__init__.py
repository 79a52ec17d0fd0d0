"""Trainers of the mask networks (`moseg train --preset masknet|whichnet`) and their data."""
