// HOST:PORT, as every address is parsed (tessera/host_port.hpp): brackets, colons and ports.
#include <gtest/gtest.h>

#include "tessera/host_port.hpp"

namespace tessera {
namespace {

TEST(HostPort, SplitsAtThePortsColon) {
    auto p = split_host_port("example.org:8080");
    ASSERT_TRUE(p);
    EXPECT_EQ(p->host, "example.org");
    EXPECT_EQ(p->port, "8080");
    EXPECT_TRUE(p->has_port);
    EXPECT_FALSE(p->bracketed);

    p = split_host_port("example.org");
    ASSERT_TRUE(p);
    EXPECT_EQ(p->host, "example.org");
    EXPECT_FALSE(p->has_port);

    p = split_host_port("h:");  // an empty port is still a port's colon
    ASSERT_TRUE(p);
    EXPECT_EQ(p->host, "h");
    EXPECT_TRUE(p->has_port);
    EXPECT_EQ(p->port, "");

    p = split_host_port("dns:///h:50051");  // unbracketed: the last colon
    ASSERT_TRUE(p);
    EXPECT_EQ(p->host, "dns:///h");
    EXPECT_EQ(p->port, "50051");
}

TEST(HostPort, BracketsHoldAnIpv6Literal) {
    auto p = split_host_port("[::1]:443");
    ASSERT_TRUE(p);
    EXPECT_EQ(p->host, "::1");
    EXPECT_EQ(p->port, "443");
    EXPECT_TRUE(p->bracketed);
    EXPECT_TRUE(p->has_port);

    p = split_host_port("[fe80::2]");
    ASSERT_TRUE(p);
    EXPECT_EQ(p->host, "fe80::2");
    EXPECT_FALSE(p->has_port);

    EXPECT_FALSE(split_host_port("[::1"));        // no ']'
    EXPECT_FALSE(split_host_port("[::1]443"));    // no ':' after ']'
    EXPECT_FALSE(split_host_port("[::1]x:443"));
}

TEST(HostPort, APortIsOneToFiveDigitsUpTo65535) {
    EXPECT_EQ(parse_port("0"), std::uint16_t{0});
    EXPECT_EQ(parse_port("80"), std::uint16_t{80});
    EXPECT_EQ(parse_port("00080"), std::uint16_t{80});
    EXPECT_EQ(parse_port("65535"), std::uint16_t{65535});
    for (const char* bad : {"", "65536", "99999", "112407", "000080", "-1", "+80", " 80", "80 ", "8o", "0x50"})
        EXPECT_FALSE(parse_port(bad)) << "'" << bad << "'";
}

}  // namespace
}  // namespace tessera
