"""The ATmega2560 target: its boards' pins, the player and its features, avr-gcc, the image."""
