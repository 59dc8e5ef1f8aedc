#include "kinematics/kdl_chain.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iomanip>
#include <random>
#include <sstream>

#include "kinematics/kinematics.hpp"
#include "test_util.hpp"

namespace pnp::kinematics {
namespace {

// A UR5-like URDF written from the DH table: joint i sits at the static part
// Tz(d) Tx(a) Rx(alpha) of row i-1 and turns about its z; tool0 is the flange.
std::string urdfFromDh(const RobotModel& m) {
    std::ostringstream x;
    x << std::setprecision(17);
    x << "<?xml version=\"1.0\"?>\n<robot name=\"" << m.name << "\">\n";
    x << "  <link name=\"base_link\"/>\n";
    for (int i = 1; i <= kAxes; ++i) x << "  <link name=\"link" << i << "\"/>\n";
    x << "  <link name=\"tool0\"/>\n";
    auto origin = [&](int row) {
        if (row < 0) return std::string("<origin xyz=\"0 0 0\" rpy=\"0 0 0\"/>");
        const DhRow& r = m.dh[row];
        std::ostringstream o;
        o << std::setprecision(17) << "<origin xyz=\"" << r.a << " 0 " << r.d << "\" rpy=\""
          << r.alpha << " 0 0\"/>";
        return o.str();
    };
    for (int i = 1; i <= kAxes; ++i) {
        x << "  <joint name=\"joint" << i << "\" type=\"revolute\">\n"
          << "    <parent link=\""
          << (i == 1 ? std::string("base_link") : "link" + std::to_string(i - 1))
          << "\"/>\n    <child link=\"link" << i << "\"/>\n    " << origin(i - 2)
          << "\n    <axis xyz=\"0 0 1\"/>\n"
          << "    <limit lower=\"-6.283185307179586\" upper=\"6.283185307179586\" effort=\"150\" "
             "velocity=\"3.14\"/>\n  </joint>\n";
    }
    x << "  <joint name=\"flange\" type=\"fixed\">\n    <parent link=\"link6\"/>\n"
      << "    <child link=\"tool0\"/>\n    " << origin(5) << "\n  </joint>\n</robot>\n";
    return x.str();
}

class TempFile {
  public:
    explicit TempFile(const std::string& text) {
        path_ = (std::filesystem::temp_directory_path() /
                 ("pnp_kinematics_" + std::to_string(::getpid()) + "_" +
                  std::to_string(counter_++) + ".urdf"))
                    .string();
        std::ofstream(path_) << text;
    }
    ~TempFile() {
        std::error_code ec;
        std::filesystem::remove(path_, ec);
    }
    const std::string& path() const { return path_; }

  private:
    static inline int counter_ = 0;
    std::string path_;
};

TEST(Urdf, ChainMatchesTheDhModel) {
    for (const RobotModel& model : {ur5(), ur10()}) {
        TempFile file(urdfFromDh(model));
        const auto chain = chainFromUrdf(file.path(), "base_link", "tool0");
        ASSERT_TRUE(chain.ok()) << chain.error().message;
        ASSERT_EQ(chain->getNrOfJoints(), 6u);
        std::mt19937_64 rng(11);
        for (int n = 0; n < 200; ++n) {
            const Joints q = test::randomJoints(rng, 2 * std::numbers::pi);
            const auto kdl = forwardKdl(*chain, q);
            ASSERT_TRUE(kdl.ok());
            ASSERT_LT(test::poseError(*kdl, forward(model, q)), 1e-9) << model.name;
        }
    }
}

TEST(Urdf, SubChain) {
    TempFile file(urdfFromDh(ur5()));
    const auto chain = chainFromUrdf(file.path(), "link2", "link4");
    ASSERT_TRUE(chain.ok()) << chain.error().message;
    EXPECT_EQ(chain->getNrOfJoints(), 2u);
}

TEST(Urdf, MissingFileIsAnError) {
    const auto chain = chainFromUrdf("/nonexistent/robot.urdf", "base_link", "tool0");
    ASSERT_FALSE(chain.ok());
    EXPECT_EQ(chain.error().code, ErrorCode::kFileNotFound);
    EXPECT_NE(chain.error().message.find("/nonexistent/robot.urdf"), std::string::npos);
}

TEST(Urdf, UnknownLinkIsAnError) {
    TempFile file(urdfFromDh(ur5()));
    for (const auto& [base, tip] : {std::pair{"base_link", "gripper"}, {"world", "tool0"}}) {
        const auto chain = chainFromUrdf(file.path(), base, tip);
        ASSERT_FALSE(chain.ok());
        EXPECT_EQ(chain.error().code, ErrorCode::kLinkNotFound);
    }
}

TEST(Urdf, MalformedFileIsAnError) {
    TempFile file("<robot name=\"broken\"><link name=\"a\"/><joint name=\"j\" type=\"revolute\">");
    const auto chain = chainFromUrdf(file.path(), "a", "b");
    ASSERT_FALSE(chain.ok());
    EXPECT_EQ(chain.error().code, ErrorCode::kParseError);
}

TEST(Kdl, ForwardChecksTheJointCount) {
    const auto r = forwardKdl(toKdlChain(ur5()), std::vector<double>{0.0, 1.0});
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kInvalidArgument);
}

TEST(Kdl, FrameConversionsRoundTrip) {
    const auto t = forward(ur5(), {0.3, -1.2, 1.5, -0.8, 1.1, 0.4});
    EXPECT_LT(test::poseError(toEigen(toKdl(t)), t), 1e-15);
}

}  // namespace
}  // namespace pnp::kinematics
