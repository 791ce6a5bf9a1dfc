"""The 8051 target (AT89C52 / STC89C52RC): its boards' pins, the player and its features, SDCC, the image."""
