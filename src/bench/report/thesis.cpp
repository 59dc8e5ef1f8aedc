#include "bench/report/thesis.hpp"

namespace pnp::bench::report::thesis {

const std::vector<int>& table43Sizes() {
    static const std::vector<int> s = {2,   4,    8,    16,   32,   64,    128,  256,
                                       512, 1024, 2048, 4096, 8192, 16384, 32768};
    return s;
}

// Transcribed from the thesis text (Table 4.3). The ACK row of OPC UA C/S has only 14 legible
// values in the source; it is kept as printed, the last column marked as not legible.
const std::vector<RttRow>& table43() {
    static const std::vector<RttRow> rows = {
        {"echo",
         "OPC UA C/S",
         "idle",
         {520, 283, 288, 280, 270, 270, 360, 313, 456, 546, 606, 978, 1003, 1171, 1770}},
        {"echo",
         "OPC UA C/S",
         "cpu",
         {279, 258, 233, 260, 276, 265, 284, 293, 310, 346, 461, 752, 830, 955, 1467}},
        {"echo",
         "OPC UA C/S",
         "net",
         {875, 869, 876, 858, 827, 864, 866, 871, 875, 860, 1056, 1158, 1248, 1397, 1894}},
        {"echo",
         "OPC UA P/S",
         "idle",
         {590, 589, 510, 338, 162, 270, 169, 174, 305, 469, 521, 446, 395, 1142, 1924}},
        {"echo",
         "OPC UA P/S",
         "cpu",
         {224, 177, 178, 182, 183, 265, 188, 206, 242, 373, 529, 620, 618, 1083, 1676}},
        {"echo",
         "OPC UA P/S",
         "net",
         {919, 930, 880, 902, 911, 864, 921, 901, 924, 936, 1003, 1019, 1110, 1286, 1641}},
        {"echo",
         "MQTT",
         "idle",
         {584, 629, 645, 641, 581, 601, 622, 699, 694, 725, 716, 920, 1186, 1225, 1511}},
        {"echo",
         "MQTT",
         "cpu",
         {912, 905, 912, 917, 911, 934, 945, 944, 964, 1015, 1094, 1540, 1582, 1504, 1843}},
        {"echo",
         "MQTT",
         "net",
         {1017, 1042, 1038, 1033, 1040, 1027, 1054, 1039, 1085, 1135, 1239, 1347, 1456, 1622,
          2029}},
        {"echo",
         "ROS",
         "idle",
         {618, 628, 446, 396, 398, 182, 296, 319, 495, 814, 698, 1007, 1273, 1486, 1823}},
        {"echo",
         "ROS",
         "cpu",
         {256, 320, 295, 252, 190, 305, 332, 317, 359, 421, 563, 1077, 1114, 952, 1427}},
        {"echo",
         "ROS",
         "net",
         {1017, 1014, 1009, 1012, 982, 1021, 1011, 963, 1040, 1063, 1124, 1263, 1343, 1488, 1884}},
        {"echo",
         "DDS",
         "idle",
         {726, 234, 236, 243, 247, 252, 251, 279, 270, 314, 343, 454, 495, 802, 1144}},
        {"echo",
         "DDS",
         "cpu",
         {624, 631, 626, 625, 624, 628, 622, 644, 659, 442, 351, 464, 489, 782, 1050}},
        {"echo",
         "DDS",
         "net",
         {1091, 1086, 1070, 1111, 1063, 1088, 1102, 1099, 1123, 1114, 1184, 1190, 1270, 1432,
          1806}},
        {"echo",
         "TCP",
         "idle",
         {250, 253, 284, 303, 254, 255, 307, 270, 289, 315, 273, 823, 811, 892, 1261}},
        {"echo",
         "UDP",
         "idle",
         {241, 231, 208, 213, 208, 162, 168, 198, 238, 193, 263, 263, 268, 893, 1398}},
        {"ack",
         "OPC UA C/S",
         "idle",
         {383, 354, 301, 294, 306, 291, 293, 321, 310, 305, 481, 710, 681, 969, -1}},
        {"ack",
         "OPC UA P/S",
         "idle",
         {185, 180, 199, 207, 196, 190, 180, 195, 215, 279, 222, 277, 298, 785, 1265}},
        {"ack",
         "MQTT",
         "idle",
         {647, 602, 556, 518, 606, 626, 636, 646, 650, 643, 629, 575, 556, 740, 800}},
        {"ack",
         "ROS",
         "idle",
         {642, 537, 321, 168, 157, 248, 623, 608, 437, 197, 226, 871, 992, 1192, 1377}},
        {"ack",
         "DDS",
         "idle",
         {320, 228, 234, 236, 241, 243, 244, 242, 252, 272, 275, 355, 343, 514, 784}},
        {"ack",
         "TCP",
         "idle",
         {235, 243, 283, 187, 239, 279, 196, 208, 189, 237, 58, 71, 81, 167, 338}},
        {"ack",
         "UDP",
         "idle",
         {259, 223, 220, 190, 155, 153, 164, 169, 174, 215, 359, 317, 255, 502, 725}},
    };
    return rows;
}

const char* table43Note() {
    return "The source text of the thesis has only 14 values for the 15 columns of the ACK / "
           "OPC UA C/S row; they are shown as printed, left-aligned, and the last cell is "
           "marked \"?\" (which column lost its value is not known).";
}

const std::vector<int>& table42Payloads() {
    static const std::vector<int> p = {0, 100, 1000, 10000};
    return p;
}

const std::vector<OverheadRow>& table42() {
    static const std::vector<OverheadRow> rows = {
        {"OPC UA C/S", {96, 196, 1096, 10096}, 632},
        {"ROS", {8, 108, 1008, 10008}, 8915},
        {"DDS", {88, 188, 1088, 10088}, 8348},
        {"MQTT", {5, 105, 1006, 10006}, 17},
    };
    return rows;
}

}  // namespace pnp::bench::report::thesis
