#!/usr/bin/env python3
"""Writes the lidar_serial fuzz target's seeds: valid LD06 packets (two revolutions,
CRC-8 poly 0x4D) and an RPLIDAR scan (response descriptor, three revolutions of 5-byte
nodes). The first byte of each seed is the chunk length the target cuts the bytes into."""
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "seeds", "lidar_serial")


def crc8(data):
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ 0x4D) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table.append(c)
    c = 0
    for x in data:
        c = table[c ^ x]
    return c


def ld06_packet(start_cdeg, ts_ms, dist_mm):
    b = bytearray([0x54, 0x2C]) + struct.pack("<HH", 3600, start_cdeg)
    for i in range(12):
        b += struct.pack("<HB", dist_mm + 3 * i, 200)
    b += struct.pack("<HH", (start_cdeg + 800) % 36000, ts_ms)
    b.append(crc8(b))
    return bytes(b)


def rplidar_node(start, quality, angle_deg, dist_mm):
    a, d, s = int(angle_deg * 64), int(dist_mm * 4), int(start)
    return bytes([(quality << 2) | ((1 - s) << 1) | s, ((a & 0x7F) << 1) | 1,
                  (a >> 7) & 0xFF, d & 0xFF, (d >> 8) & 0xFF])


def main():
    os.makedirs(OUT, exist_ok=True)
    ld = bytearray([47])
    ts = 0
    for _ in range(2):
        for k in range(45):
            ld += ld06_packet(k * 800, ts, 1000 + 30 * abs(k % 20 - 10))
            ts = (ts + 2) % 30000
    with open(os.path.join(OUT, "ld06-2rev"), "wb") as f:
        f.write(ld)
    rp = bytearray([64, 0xA5, 0x5A, 0x05, 0x00, 0x00, 0x40, 0x81])
    for _ in range(3):
        for i in range(360):
            rp += rplidar_node(i == 0, 47, float(i), 800 + 400 * abs(i % 90 - 45) / 45)
    with open(os.path.join(OUT, "rplidar-3rev"), "wb") as f:
        f.write(rp)


if __name__ == "__main__":
    main()
