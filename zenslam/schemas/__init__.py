"""Message definitions, their encoder/decoder and key expressions."""
