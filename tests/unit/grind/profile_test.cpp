#include "core/grind/profile.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace nccomp::core::grind {
namespace {

std::string error_of(auto&& fn) {
  try {
    fn();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "no error";
}

TEST(ProfileCsv, GivenHeaderCommentsBlankLinesAndCrlf_ThenSamplesWithLines) {
  const auto s =
      parse_profile_csv("# roll 17\r\nz_mm,u_mm\r\n0,0.5\r\n\r\n 1.5 , +0.25\n3,-1e-3", "p.csv");
  ASSERT_EQ(s.z_mm.size(), 3U);
  EXPECT_DOUBLE_EQ(s.z_mm[1], 1.5);
  EXPECT_DOUBLE_EQ(s.u_mm[1], 0.25);
  EXPECT_DOUBLE_EQ(s.u_mm[2], -0.001);
  EXPECT_EQ(s.line[0], 3U);
  EXPECT_EQ(s.line[2], 6U);
}

// Fed in pieces split anywhere (inside numbers, between CR and LF, at line ends), the parser
// gives what it gives on the whole text: the same samples and lines, or the same error.
TEST(ProfileCsv, GivenTextInPieces_ThenSameAsWhole) {
  const std::string texts[] = {
      "# roll 17\r\nz_mm,u_mm\r\n0,0.5\r\n\r\n 1.5 , +0.25\n3,-1e-3",
      "0,1\n1,2\n2,3\n",
      "0,1\n1,2\n1,3\n",      // error on line 3
      "0,1\n1,nan\n2,3",      // error on line 2
      "z_mm,u_mm\n0,1\n5,2",  // last line without a line end
  };
  for (const auto& text : texts) {
    const std::string whole = error_of([&] { parse_profile_csv(text, "p.csv"); });
    for (std::size_t cut1 = 0; cut1 <= text.size(); ++cut1) {
      for (std::size_t cut2 = cut1; cut2 <= text.size(); cut2 += 3) {
        ProfileCsvParser parser("p.csv");
        std::string err = "no error";
        SampledProfile s;
        try {
          parser.feed(std::string_view(text).substr(0, cut1));
          parser.feed(std::string_view(text).substr(cut1, cut2 - cut1));
          parser.feed(std::string_view(text).substr(cut2));
          s = parser.finish();
        } catch (const std::invalid_argument& e) {
          err = e.what();
        }
        ASSERT_EQ(err, whole) << cut1 << "/" << cut2;
        if (whole == "no error") {
          const auto w = parse_profile_csv(text, "p.csv");
          ASSERT_EQ(s.z_mm, w.z_mm);
          ASSERT_EQ(s.u_mm, w.u_mm);
          ASSERT_EQ(s.line, w.line);
        }
      }
    }
  }
}

TEST(ProfileCsv, GivenOverlongLine_ThenErrorNamesTheLineWholeOrInPieces) {
  const std::string text = "0,1\n1," + std::string(kMaxProfileCsvLineBytes, '0') + "\n2,3\n";
  EXPECT_EQ(error_of([&] { parse_profile_csv(text, "a.csv"); }),
            "a.csv:2: line longer than 4096 characters");
  ProfileCsvParser parser("a.csv");
  parser.feed("0,1\n1,");
  EXPECT_EQ(error_of([&] {
              for (int i = 0; i < 5000; ++i) {
                parser.feed("0");  // no line end ever: refused before it grows without bound
              }
            }),
            "a.csv:2: line longer than 4096 characters");
}

// Uniform samples taken by value: u is moved (same buffer), z and line freed.
TEST(ProfileUniform, GivenUniformSamplesByValue_ThenUIsMovedNotCopied) {
  auto s = parse_profile_csv("0,1\n0.5,2\n1,4\n", "p.csv");
  const double* data = s.u_mm.data();
  const auto p = to_uniform(std::move(s), 0.0, "p.csv");
  EXPECT_EQ(p.u_mm.data(), data);
  EXPECT_DOUBLE_EQ(p.spacing_mm, 0.5);
  EXPECT_EQ(p.u_mm, (std::vector<double>{1.0, 2.0, 4.0}));
  EXPECT_TRUE(s.z_mm.empty());  // NOLINT(bugprone-use-after-move): documented to be emptied
  // Non-uniform ones are resampled as before (or refused naming the line).
  auto n = parse_profile_csv("0,0\n1,1\n3,3\n", "p.csv");
  EXPECT_EQ(error_of([&] { (void)to_uniform(std::move(n), 0.0, "p.csv"); }),
            "p.csv:3: samples are not uniformly spaced (z = 3.000000, uniform spacing would put it "
            "at 2.000000); give a resampling spacing");
  auto r = parse_profile_csv("0,0\n1,1\n3,3\n", "p.csv");
  const auto q = to_uniform(std::move(r), 0.5, "p.csv");
  EXPECT_EQ(q.size(), 7U);
  EXPECT_DOUBLE_EQ(q.u_mm[5], 2.5);
}

TEST(ProfileCsv, GivenBadInput_ThenErrorNamesFileAndLine) {
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1\n1,nan\n", "a.csv"); }),
            "a.csv:2: value is not finite (NaN or inf)");
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1\n0,2\n", "a.csv"); }),
            "a.csv:2: z_mm must increase strictly: 0.000000 after 0.000000");
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1\n-1,2\n", "a.csv"); }).substr(0, 9), "a.csv:2: ");
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1\n1;2\n", "a.csv"); }),
            "a.csv:2: expected two fields 'z_mm,u_mm', got '1;2'");
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1,2\n", "a.csv"); }),
            "a.csv:1: expected two fields 'z_mm,u_mm', got more: '0,1,2'");
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1\n1,x\n", "a.csv"); }),
            "a.csv:2: u_mm is not a number: 'x'");
  EXPECT_EQ(error_of([] { parse_profile_csv("1e,1\n", "a.csv"); }),
            "a.csv:1: z_mm is not a number: '1e'");
  EXPECT_EQ(error_of([] { parse_profile_csv("z_mm,u_mm\n0,1\n", "a.csv"); }),
            "a.csv: needs at least 2 samples, got 1");
  EXPECT_EQ(error_of([] { parse_profile_csv("", "a.csv"); }),
            "a.csv: needs at least 2 samples, got 0");
  // A header only counts as the first content line.
  EXPECT_EQ(error_of([] { parse_profile_csv("0,1\nz_mm,u_mm\n", "a.csv"); }),
            "a.csv:2: z_mm is not a number: 'z_mm'");
}

TEST(ProfileUniform, GivenUniformSamples_ThenTakenAsIs) {
  const auto s = parse_profile_csv("0,1\n0.1,2\n0.2,3\n0.3,4\n", "u.csv");
  const auto u = to_uniform(s, 0.0, "u.csv");
  EXPECT_DOUBLE_EQ(u.z0_mm, 0.0);
  EXPECT_NEAR(u.spacing_mm, 0.1, 1e-15);
  EXPECT_EQ(u.u_mm, s.u_mm);
  EXPECT_NEAR(u.interpolate(0.15), 2.5, 1e-12);
  EXPECT_DOUBLE_EQ(u.interpolate(-1.0), 1.0);
  EXPECT_DOUBLE_EQ(u.interpolate(9.0), 4.0);
}

TEST(ProfileUniform, GivenNonUniformSamples_ThenErrorOrResampling) {
  const auto s = parse_profile_csv("# x\n0,0\n1,1\n3,3\n4,2\n", "n.csv");
  EXPECT_EQ(error_of([&] { to_uniform(s, 0.0, "n.csv"); }).substr(0, 52),
            "n.csv:4: samples are not uniformly spaced (z = 3.000");
  const auto u = to_uniform(s, 0.5, "n.csv");
  ASSERT_EQ(u.size(), 9U);
  EXPECT_NEAR(u.u_mm[4], 2.0, 1e-12);  // z = 2 between (1,1) and (3,3)
  EXPECT_NEAR(u.u_mm[7], 2.5, 1e-12);  // z = 3.5 between (3,3) and (4,2)
  EXPECT_NEAR(u.u_mm[8], 2.0, 1e-12);
}

TEST(ProfileFamily, GivenEachFamily_ThenItsFormula) {
  FamilySpec f;
  f.z_from_mm = -500;
  f.z_to_mm = 500;
  f.spacing_mm = 0.5;
  f.family = Family::kConvexCrown;
  f.height_mm = 0.6;
  auto p = generate_profile(f);
  ASSERT_EQ(p.size(), 2001U);
  EXPECT_NEAR(p.u_mm[1000], 0.6, 1e-15);
  EXPECT_NEAR(p.u_mm[0], 0.0, 1e-15);
  EXPECT_NEAR(p.u_mm[500], 0.45, 1e-12);  // z = −250: 0.6·(1 − 1/4)
  f.family = Family::kConcaveCrown;
  EXPECT_NEAR(generate_profile(f).u_mm[1000], -0.6, 1e-15);
  f.family = Family::kStraight;
  f.slope = 0.001;
  f.offset_mm = 2.0;
  EXPECT_NEAR(generate_profile(f).u_mm[2000], 2.5, 1e-12);
  f.family = Family::kSine;
  f.amplitude_mm = 0.1;
  f.wavelength_mm = 400.0;
  f.phase_rad = 0.0;
  f.z_ref_given = true;
  f.z_ref_mm = -500.0;
  EXPECT_NEAR(generate_profile(f).u_mm[200], 2.1, 1e-12);  // z = −400: quarter wave
  f.family = Family::kCvc;
  f.coef = {0.0, 1e-3, 0.0, 2e-9};
  f.z_ref_given = false;  // about the middle
  EXPECT_NEAR(generate_profile(f).u_mm[2000], 0.5 + 2e-9 * 1.25e8, 1e-12);
  f.family = Family::kPolynomial;
  f.coef = {1.0, 0.0, -1e-6};
  EXPECT_NEAR(generate_profile(f).u_mm[0], 0.75, 1e-12);
}

TEST(ProfileFamily, GivenBadParameters_ThenClearErrors) {
  FamilySpec f;
  f.z_from_mm = 0;
  f.z_to_mm = 10;
  f.spacing_mm = 0.0;
  EXPECT_EQ(error_of([&] { generate_profile(f); }), "profile family: spacing_mm must be > 0");
  f.spacing_mm = 1.0;
  f.z_to_mm = -1;
  EXPECT_EQ(error_of([&] { generate_profile(f); }),
            "profile family: z_to_mm must be greater than z_from_mm");
  f.z_to_mm = 10;
  f.family = Family::kCvc;
  f.coef = {1, 2};
  EXPECT_EQ(error_of([&] { generate_profile(f); }),
            "profile family cvc: needs exactly 4 coefficients c0..c3, got 2");
  f.family = Family::kSine;
  EXPECT_EQ(error_of([&] { generate_profile(f); }),
            "profile family sine: wavelength_mm must be > 0");
  f.family = Family::kStraight;
  f.slope = std::nan("");
  EXPECT_EQ(error_of([&] { generate_profile(f); }), "profile family: slope must be finite");
  EXPECT_EQ(error_of([] { parse_family("crowned"); }),
            "unknown profile family 'crowned' (straight, convex, concave, cvc, sine, poly)");
  EXPECT_EQ(parse_family("cvc"), Family::kCvc);
}

}  // namespace
}  // namespace nccomp::core::grind
