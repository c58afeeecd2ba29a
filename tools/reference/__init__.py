"""The PyTorch reference of the official models (SRT / RP-SRT, OSRT / RP-OSRT, DeFiNe / RP-DeFiNe), the MSN-Easy
cameras, the official run configs and the byte-stable safetensors writer."""
