"""Teach: the method on one 2D image (``lesson2d``) and exercises that check a piece of the method you wrote."""
