// The shared LoD rule (tessera/scene/lod.hpp): known derivatives per filter, anisotropy, bias,
// clamping and the NaN / infinity / zero cases.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "tessera/scene/lod.hpp"

namespace {

using tessera::scene::LodRule;
using tessera::scene::lod_from_derivatives;
using tessera::scene::SampleFilter;
using tessera::scene::wanted_level;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

LodRule rule(SampleFilter f, std::uint32_t aniso = 8) { return LodRule{f, aniso}; }

TEST(Lod, IsotropicDerivatives) {
    for (SampleFilter f : {SampleFilter::bilinear, SampleFilter::trilinear}) {
        EXPECT_FLOAT_EQ(lod_from_derivatives(1, 0, 0, 1, rule(f)), 0.0f);
        EXPECT_FLOAT_EQ(lod_from_derivatives(2, 0, 0, 2, rule(f)), 1.0f);
        EXPECT_FLOAT_EQ(lod_from_derivatives(0.25, 0, 0, 0.25, rule(f)), -2.0f);
        // rho is the length of the derivative vector: (3, 4) per pixel is 5 texels.
        EXPECT_FLOAT_EQ(lod_from_derivatives(3, 4, 0, 1, rule(f)), static_cast<float>(std::log2(5.0)));
        // The major axis decides for bilinear and trilinear.
        EXPECT_FLOAT_EQ(lod_from_derivatives(8, 0, 0, 1, rule(f)), 3.0f);
        EXPECT_FLOAT_EQ(lod_from_derivatives(1, 0, 0, -8, rule(f)), 3.0f);
    }
}

TEST(Lod, AnisotropicUsesTheMinorAxisUpToTheRatioCap) {
    const LodRule a8 = rule(SampleFilter::anisotropic, 8);
    EXPECT_FLOAT_EQ(lod_from_derivatives(8, 0, 0, 1, a8), 0.0f);   // ratio 8: the minor axis
    EXPECT_FLOAT_EQ(lod_from_derivatives(4, 0, 0, 1, a8), 0.0f);   // ratio 4: the minor axis
    EXPECT_FLOAT_EQ(lod_from_derivatives(16, 0, 0, 1, a8), 1.0f);  // ratio 16 > 8: major / 8 = 2
    EXPECT_FLOAT_EQ(lod_from_derivatives(16, 0, 0, 4, a8), 2.0f);  // minor 4 > major / 8 = 2
    const LodRule a2 = rule(SampleFilter::anisotropic, 2);
    EXPECT_FLOAT_EQ(lod_from_derivatives(16, 0, 0, 1, a2), 3.0f);  // major / 2 = 8
    // max_anisotropy is clamped to 1..8.
    EXPECT_FLOAT_EQ(lod_from_derivatives(16, 0, 0, 1, rule(SampleFilter::anisotropic, 0)), 4.0f);
    EXPECT_FLOAT_EQ(lod_from_derivatives(64, 0, 0, 1, rule(SampleFilter::anisotropic, 100)), 3.0f);
}

TEST(Lod, WantedLevelPerFilter) {
    // Bilinear rounds to the nearest level, trilinear and anisotropic take the finer of the two.
    EXPECT_EQ(wanted_level(0.49f, SampleFilter::bilinear, 10), 0u);
    EXPECT_EQ(wanted_level(0.5f, SampleFilter::bilinear, 10), 1u);
    EXPECT_EQ(wanted_level(1.49f, SampleFilter::bilinear, 10), 1u);
    EXPECT_EQ(wanted_level(0.99f, SampleFilter::trilinear, 10), 0u);
    EXPECT_EQ(wanted_level(1.0f, SampleFilter::trilinear, 10), 1u);
    EXPECT_EQ(wanted_level(2.7f, SampleFilter::anisotropic, 10), 2u);
    const float lod3 = lod_from_derivatives(3, 0, 0, 3, rule(SampleFilter::trilinear));  // log2(3) = 1.58
    EXPECT_EQ(wanted_level(lod3, SampleFilter::trilinear, 10), 1u);
    EXPECT_EQ(wanted_level(lod3, SampleFilter::bilinear, 10), 2u);
    // Bias is added before the rule.
    EXPECT_EQ(wanted_level(lod3 + 1.0f, SampleFilter::trilinear, 10), 2u);
    EXPECT_EQ(wanted_level(lod3 - 3.0f, SampleFilter::trilinear, 10), 0u);
}

TEST(Lod, ClampsToTheLevels) {
    for (SampleFilter f : {SampleFilter::bilinear, SampleFilter::trilinear, SampleFilter::anisotropic}) {
        EXPECT_EQ(wanted_level(-5.0f, f, 8), 0u);
        EXPECT_EQ(wanted_level(7.0f, f, 8), 7u);
        EXPECT_EQ(wanted_level(100.0f, f, 8), 7u);
        EXPECT_EQ(wanted_level(1e30f, f, 8), 7u);
        EXPECT_EQ(wanted_level(3.0f, f, 1), 0u);  // a one-level texture
        EXPECT_EQ(wanted_level(3.0f, f, 0), 0u);  // out of contract, still safe
    }
}

TEST(Lod, NanInfinityAndZeroDerivatives) {
    for (SampleFilter f : {SampleFilter::bilinear, SampleFilter::trilinear, SampleFilter::anisotropic}) {
        const LodRule r = rule(f);
        // Zero derivatives: -inf, level 0.
        const float zero = lod_from_derivatives(0, 0, 0, 0, r);
        EXPECT_TRUE(std::isinf(zero) && zero < 0) << zero;
        EXPECT_EQ(wanted_level(zero, f, 12), 0u);
        // NaN anywhere: NaN, level 0.
        for (int which = 0; which < 4; ++which) {
            double d[4] = {1, 0, 0, 1};
            d[which] = kNaN;
            const float l = lod_from_derivatives(d[0], d[1], d[2], d[3], r);
            EXPECT_TRUE(std::isnan(l)) << which;
            EXPECT_EQ(wanted_level(l, f, 12), 0u);
        }
        // Infinite derivatives: +inf, the last level.
        const float inf = lod_from_derivatives(kInf, 0, 0, kInf, r);
        EXPECT_TRUE(std::isinf(inf) && inf > 0) << inf;
        EXPECT_EQ(wanted_level(inf, f, 12), 11u);
        EXPECT_EQ(wanted_level(std::numeric_limits<float>::infinity(), f, 12), 11u);
        EXPECT_EQ(wanted_level(-std::numeric_limits<float>::infinity(), f, 12), 0u);
        EXPECT_EQ(wanted_level(std::numeric_limits<float>::quiet_NaN(), f, 12), 0u);
    }
    // Anisotropic with one axis zero: the cap keeps the lod finite.
    EXPECT_FLOAT_EQ(lod_from_derivatives(16, 0, 0, 0, rule(SampleFilter::anisotropic, 8)), 1.0f);
}

}  // namespace
