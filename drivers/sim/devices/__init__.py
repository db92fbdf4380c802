"""The simulated devices: each chip's registers and each controller's protocol, answering as its datasheet
says, reading and driving the one world."""
