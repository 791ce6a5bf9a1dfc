"""The toolpath: the front ends' items in machine millimetres, and the segments they flatten into."""
