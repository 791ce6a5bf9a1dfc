"""printer-codegen: host-side motion maths, firmware that only plays tables back."""

__version__ = "0.1.0"
